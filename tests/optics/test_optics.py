"""Skin-optics profiles: sourced numbers, the diffusion operator, and the paper's Table 1 order."""

import numpy as np
import pytest
import scipy.integrate
import scipy.ndimage

from skintopo.errors import SkinTopoError
from skintopo.optics import (
    JENSEN_2001_SKIN,
    LITERATURE,
    ScatteringProfile,
    dipole_diffuse_reflectance,
)

# field notes, "Skin": diffuse albedo at ~625/523/462 nm (NCSU skin reflectance data)
FIELD_NOTES_ALBEDO = {"light": (0.60, 0.41, 0.33), "dark": (0.42, 0.22, 0.13)}


def dipole_profile(radius_mm, reduced_scattering, absorption, eta=1.3):
    """Jensen et al. 2001, eq. 4: the dipole's radial diffuse reflectance R_d(r) (1/mm^2),
    written out independently of the package's closed form for its integral."""
    extinction = reduced_scattering + absorption
    albedo = reduced_scattering / extinction
    effective = np.sqrt(3 * absorption * extinction)
    fresnel = -1.440 / eta**2 + 0.710 / eta + 0.668 + 0.0636 * eta
    real = 1 / extinction
    virtual = real * (1 + 4 / 3 * (1 + fresnel) / (1 - fresnel))
    d_real, d_virtual = np.hypot(radius_mm, real), np.hypot(radius_mm, virtual)
    return albedo / (4 * np.pi) * (real * (effective * d_real + 1) * np.exp(-effective * d_real) / d_real**3
                                   + virtual * (effective * d_virtual + 1) * np.exp(-effective * d_virtual) / d_virtual**3)


@pytest.mark.parametrize("measurement", ["skin1", "skin2"])
def test_dipole_total_reflectance_is_the_integral_of_its_profile(measurement):
    coefficients = JENSEN_2001_SKIN[measurement]
    for s, a in zip(coefficients["reduced_scattering"], coefficients["absorption"]):
        integral, _ = scipy.integrate.quad(lambda r: 2 * np.pi * r * dipole_profile(r, s, a), 0, np.inf, limit=200)
        assert dipole_diffuse_reflectance(s, a) == pytest.approx(integral, rel=1e-6)


def test_literature_albedo_within_10_percent_of_the_field_notes():
    for skin, expected in FIELD_NOTES_ALBEDO.items():
        found = [LITERATURE.albedo[skin][band] for band in ("red", "green", "blue")]
        print(skin, "literature albedo", found, "field notes", expected)
        np.testing.assert_allclose(found, expected, rtol=0.10)


def test_scattering_operator_is_a_reflecting_gaussian_blur_that_conserves_light():
    rng = np.random.default_rng(0)
    image = rng.random((48, 70))
    narrow = ScatteringProfile((0.3, 0.7), (0.0, 60.0)).operator(image.shape, 20.0)  # sigma 3 px
    expected = 0.3 * image + 0.7 * scipy.ndimage.gaussian_filter(image, 3.0, mode="reflect", truncate=10)
    np.testing.assert_allclose(narrow(image), expected, atol=1e-10)
    # wider than the field: reflected, not truncated; light is neither created nor lost
    wide = LITERATURE.scattering["red"].operator(image.shape, 20.0)
    assert wide(image).mean() == pytest.approx(image.mean(), rel=1e-12)
    assert ScatteringProfile((1.0,), (0.0,)).operator(image.shape, 20.0) is None
    with pytest.raises(SkinTopoError, match="sum to 1"):
        ScatteringProfile((0.5, 0.4), (0.0, 10.0))


def test_literature_profile_is_heavy_tailed_and_widest_in_red():
    widths = {band: LITERATURE.diffusion_width_um(band) for band in ("red", "green", "blue")}
    assert widths["red"] > 2 * widths["green"] > 2 * widths["blue"]
    # heavy-tailed: light concentrated near its entry point plus a long tail, so at a 2 mm wavelength
    # red keeps far more contrast (0.36) than a Gaussian of the same RMS radius (1.7 mm) would (0.001)
    f = 1 / 2000.0
    gaussian = np.exp(-2 * np.pi**2 * (widths["red"] / np.sqrt(2)) ** 2 * f**2)
    assert LITERATURE.scattering["red"].transfer(f) > 10 * gaussian
