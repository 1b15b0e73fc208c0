"""The paper's spectral correction, exactly, and the feathered variant against its closed form."""

import numpy as np
import pytest
from scipy.special import ndtr

from skintopo.correction import correct_slopes, spectral_correction, substitution_weight
from skintopo.errors import SkinTopoError


def test_feathered_weight_follows_the_closed_form_of_a_blurred_straight_border():
    """Mask = columns left of a straight border; outside it w = 2 Phi(-d / sigma), sigma = feather / 2."""
    mask = np.zeros((60, 120), bool)
    mask[:, :50] = True
    weight = substitution_weight(mask, (10.0, 10.0), method="feathered", feather_um=150.0)
    distance = np.arange(50, 120) - 49.5  # pixels from the border (pixel centres)
    expected = np.clip(2 * ndtr(-distance / 7.5), 0, 1)
    np.testing.assert_allclose(weight[30, 50:], expected, atol=2e-3)
    assert (weight[:, :50] == 1).all()
    np.testing.assert_array_equal(substitution_weight(mask, 10.0, method="paper"), mask.astype(float))
    across = substitution_weight(mask.T, (10.0, 20.0), method="feathered", feather_um=150.0)  # border along x, rectangular pixels
    np.testing.assert_allclose(across[50:, 30], expected, atol=2e-3)  # sigma in rows: 7.5 pixels of 10 um
    labels = np.where(mask, 2, 0)  # a label image as the mask: non-zero is wrinkle
    np.testing.assert_array_equal(substitution_weight(labels, (10.0, 10.0), method="feathered", feather_um=150.0), weight)


def test_feathered_correction_keeps_red_far_from_the_wrinkle_and_the_minimum_inside():
    rows, columns = 200, 96
    y, x = np.mgrid[:rows, :columns] * 10.0
    groove = 40.0 * np.exp(-(((y - 1000.0) / 60.0) ** 2))  # a straight groove along x, 40 um deep, mid-field
    slope_y = -np.gradient(-groove, 10.0, axis=0)  # dz/dy with y up: rows go down
    mask = groove > 20.0
    red = (np.zeros_like(x), 0.6 * slope_y)  # red too shallow, green and blue too deep
    green = blue = (np.zeros_like(x), 1.3 * slope_y)
    corrected, z_red, z_a = correct_slopes(red, green, blue, mask, 10.0, method="feathered", feather_um=60.0)
    weight = substitution_weight(mask, 10.0, method="feathered", feather_um=60.0)  # narrower than the default
    far = weight == 0
    assert far.sum() > 0.3 * far.size  # the feather (4 sigma) ends well inside the field
    assert (substitution_weight(mask, 10.0, method="feathered")[far] > 0).any()  # where the default feather would blend
    offset = np.median((corrected.z - z_red.z)[far])
    np.testing.assert_allclose(corrected.z[far] - offset, z_red.z[far], atol=1e-6)
    inside = mask
    np.testing.assert_allclose(corrected.z[inside], np.minimum(z_a.z, z_red.z)[inside], atol=1e-6)
    with pytest.raises(Exception, match="unknown correction method"):
        correct_slopes(red, green, blue, mask, 10.0, method="blend")


def test_correction_is_exactly_the_papers_algorithm_on_known_slopes():
    rng = np.random.default_rng(0)
    shape = (40, 50)
    red, green, blue = ((rng.normal(size=shape) * 0.1, rng.normal(size=shape) * 0.1) for _ in range(3))
    mask = np.zeros(shape, bool)
    mask[15:25, 10:40] = True
    corrected, z_red, z_a = correct_slopes(red, green, blue, mask, 10.0, integrator="dct-poisson")
    t1 = (red[0] + (green[0] + blue[0]) / 2) / 2
    t2 = (red[1] + (green[1] + blue[1]) / 2) / 2
    from skintopo.height import dct_poisson

    expected_red = dct_poisson(*red, 10.0)
    expected_a = dct_poisson(np.where(mask, t1, red[0]), np.where(mask, t2, red[1]), 10.0)
    expected_a -= np.median((expected_a - expected_red)[~mask])
    np.testing.assert_allclose(z_red.z, expected_red)
    np.testing.assert_allclose(corrected.z, np.where(mask, np.minimum(expected_a, expected_red), expected_red))
    for band in (green, blue, red):  # a missing slope in any band, or outside the mask, is a missing height
        holes = (np.where(np.arange(50) == 45, np.nan, band[0]), band[1])  # dz/dx missing, dz/dy known
        bands = [holes if b is band else b for b in (red, green, blue)]
        outside = np.ones(shape, bool)
        outside[:5] = False
        corrected, z_red, z_a = correct_slopes(*bands, mask, 10.0, integrator="least-squares", mask=outside)
        assert np.isnan(corrected.z[:, 45][mask[:, 45]]).all() and np.isnan(corrected.z[:5]).all()
        assert (~corrected.mask[:5]).all() and np.isfinite(corrected.z[5:, :45]).all()


def test_correction_needs_three_bands():
    with pytest.raises(SkinTopoError, match=r"missing \['blue'\]"):
        spectral_correction({"red": np.zeros((4, 4, 3)), "green": np.zeros((4, 4, 3))}, 1.0)


def test_spectral_correction_of_scaled_slopes_reads_the_combined_depth_inside_the_wrinkle():
    """Red slopes 0.6 x the truth (too shallow), green and blue 1.3 x (too deep): the combined
    slopes T are (0.6 + 1.3) / 2 = 0.95 x the truth, so inside the wrinkle the corrected height
    (min of z_a and z_red) is 0.95 of the true depth and red's is 0.6; outside the mask nothing
    is returned. The wrinkle is found on the combined height (the default segmentation)."""
    from skintopo.synth import make_surface
    from skintopo.synth.surfaces import SurfaceSpec, Wrinkle
    from tests.helpers.analytic import normals_from_slopes

    wrinkle = Wrinkle(depth_um=100.0, width_um=500.0, length_um=3000.0, orientation_deg=10.0, shape="U")
    surface = make_surface(SurfaceSpec(size_px=(160, 160), pixel_um=20.0, wrinkles=(wrinkle,), microrelief=False,
                                       roughness_rms_um=0.0, form_radius_mm=None), seed=0)
    bands = {"red": 0.6, "green": 1.3, "blue": 1.3}
    normals = {band: normals_from_slopes(k * surface.p, k * surface.q) for band, k in bands.items()}
    mask = np.ones(surface.height.shape, bool)
    mask[:, :8] = False
    groove = np.zeros(surface.height.shape)
    groove[:, 1:7] = 2.0 * np.sign(np.arange(6) - 2.5)  # a steep V outside the mask: never measured, never a wrinkle
    for band in normals:
        normals[band] = np.where(mask[..., None], normals[band], normals_from_slopes(groove, np.zeros_like(groove)))
    result = spectral_correction(normals, 20.0, mask=mask)
    assert result.segmentation.count == 1 and result.method == "paper"
    np.testing.assert_array_equal(result.red_height.mask, result.height.mask)
    np.testing.assert_array_equal(result.interim_height.mask, result.height.mask)
    floor = surface.wrinkle_depth > 0.9 * wrinkle.depth_um
    skin = (surface.wrinkle_depth == 0) & mask

    def depth(z):
        return np.median(z[skin]) - np.median(z[floor])

    assert depth(result.height.z) == pytest.approx(0.95 * wrinkle.depth_um, rel=0.05)
    assert depth(result.red_height.z) == pytest.approx(0.6 * wrinkle.depth_um, rel=0.05)
    assert depth(result.interim_height.z) == pytest.approx(0.95 * wrinkle.depth_um, rel=0.05)
    assert np.isnan(result.height.z[:, :8]).all() and np.isfinite(result.height.z[mask]).all()
    with pytest.raises(SkinTopoError, match="unknown correction method"):
        spectral_correction(normals, 20.0, mask=mask, segmentation=result.segmentation, method="blend")
    from skintopo.height import integrate_slopes, normals_to_gradients

    fourier = spectral_correction(normals, 20.0, mask=mask, segmentation=result.segmentation, integrator="frankot-chellappa")
    red = integrate_slopes(*normals_to_gradients(normals["red"]), 20.0, mask=mask, method="frankot-chellappa")
    np.testing.assert_allclose(fourier.red_height.z, red.z, atol=1e-9)
